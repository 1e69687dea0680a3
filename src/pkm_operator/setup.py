from setuptools import setup

package_name = 'pkm_operator'

setup(
    name=package_name,
    version='0.1.0',
    packages=[package_name],
    # the operator panel's page (pkm-panel serves it from the package directory)
    package_data={package_name: ['panel_static/*']},
    data_files=[
        ('share/ament_index/resource_index/packages',
            ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='PKM controller developers',
    maintainer_email='pkm-dev@pkm-controller.org',
    description=(
        'The operator: the web panel (its pure core, the ASGI app, the rclpy node) and the live Foxglove bridge.'
    ),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'pkm-panel = pkm_operator.panel_main:main',
            'foxglove_bridge = pkm_operator.foxglove_bridge_node:main',
        ],
    },
)
