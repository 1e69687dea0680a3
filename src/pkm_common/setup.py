from setuptools import setup

package_name = 'pkm_common'

setup(
    name=package_name,
    version='0.1.0',
    packages=[package_name],
    package_data={package_name: ['fastdds_localhost_udp.xml']},
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
        'Shared ROS helpers of the PKM nodes: QoS profiles per topic, '
        'message conversions, validated parameters, node runner.'
    ),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [],
    },
)
